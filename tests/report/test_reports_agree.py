"""Every report says what the finding says: the same frame numbers, the same status, the finding's
text also for an expected failure, a replay line that pastes into a shell, which model ran, and
a terminal table that cuts nothing."""
from __future__ import annotations

import html
import json
import re
import shlex
import shutil

import numpy as np
import pytest

from conftest import REPO_ROOT, speed_scenario

try:  # before any pytester run: a module first imported inside one is dropped after it
    import torch
except ImportError:
    torch = None
needs_torch = pytest.mark.skipif(torch is None, reason="torch not installed")

CLOSED_LOOP = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
{extra}Evaluation:
  UseCaseName: closed_loop
  UseCaseFormatVersion: 0.1.0
  Datasets:
    - logs: {{Path: gen.zarr}}
  Model: {model}
  Unroll: {{Scenes: [3], StartFrame: 10, Steps: 40}}
  Conditions:
    Collisions: {{Front: 0, Side: 0, Rear: 0, AtFaultOnly: true}}
"""


def summary_records(pytester, output="driveeval-results") -> dict:
    data = json.loads((pytester.path / output / "summary.json").read_text())
    return {r["nodeid"]: r for r in data["results"]}


# --- 1. frame numbers --------------------------------------------------------------------------

def _label_mask(image, colour) -> np.ndarray:
    """Pixels of the caption's colour in the strip the caption is drawn in."""
    rgb = np.asarray(image.convert("RGB"), dtype=int)[:16]
    return np.abs(rgb - np.asarray(colour)).max(axis=-1) < 60


def frames_captioned(gif, title: str, candidates) -> list[int]:
    """The frame number each frame of ``gif`` shows in its caption, read by matching the caption
    against each candidate's caption as Pillow draws it (collision frames in red, others dark)."""
    from PIL import Image, ImageDraw, ImageSequence

    from pytest_driveeval.report.birdseye import COLLISION, TEXT, frame_label

    def drawn(text, colour, width):
        blank = Image.new("RGB", (width, 32), (250, 250, 250))
        ImageDraw.Draw(blank).text((4, 4), text, fill=colour)
        return _label_mask(blank, colour)

    read = []
    for image in ImageSequence.Iterator(Image.open(gif)):
        collision = _label_mask(image, COLLISION).sum() > 20
        colour = COLLISION if collision else TEXT
        mask = _label_mask(image, colour)

        def overlap(n):
            expected = drawn(frame_label(title, n, collision), colour, image.width)
            return (mask & expected).sum() / max(1, (mask | expected).sum())

        read.append((max(candidates, key=overlap), collision))
    return read


@needs_torch
def test_the_animation_names_a_collision_by_the_frame_the_finding_and_closed_loop_json_name(pytester):
    shutil.copytree(REPO_ROOT / "fixtures" / "l5kit" / "generated.zarr", pytester.path / "gen.zarr")
    pytester.makefile(".scenario.yaml", cv=CLOSED_LOOP.format(name="cv", extra="", model="constant_velocity"))
    pytester.runpytest("-q").assert_outcomes(failed=1)
    (record,) = summary_records(pytester).values()
    folder = pytester.path / "driveeval-results"
    scenes = json.loads((folder / record["artefacts"]["result"]).read_text())["scenes"]
    in_json = [c["frame"] for c in scenes[0]["collisions"]]
    assert in_json and min(in_json) >= 10  # StartFrame: 10, so a frame counted from the start would be < 40
    (finding,) = [f for f in record["findings"] if f.get("frame") is not None]
    assert finding["frame"] == min(in_json) and f"first at frame {min(in_json)}" in finding["message"]
    # captioned with the scene's index and its zarr, as the findings name it
    shown = frames_captioned(folder / record["artefacts"]["scene_3_gif"], "scene 3 (gen.zarr)", range(0, 60))
    assert [frame for frame, collision in shown if collision] == in_json
    assert shown[0] == (10, False)  # the animation starts at the scenario's StartFrame


# --- 2. allure: failed for a scenario's conditions, broken for bad input ----------------------

def test_allure_says_failed_for_unmet_conditions_and_broken_for_missing_data(project):
    project.makefile(".scenario.yaml", too_fast=speed_scenario("too-fast", datasets=("fast.csv",)),
                     nodata=speed_scenario("nodata", datasets=("absent.csv",)))
    project.runpytest("-q", "--alluredir=allure").assert_outcomes(failed=1, errors=1)
    results = [json.loads(p.read_text()) for p in (project.path / "allure").glob("*-result.json")]
    status = {r["fullName"].split("#")[0].split(".")[0]: r["status"] for r in results}
    assert status == {"too_fast": "failed", "nodata": "broken"}, [(r["fullName"], r["status"]) for r in results]
    (failed,) = [r for r in results if r["status"] == "failed"]
    assert "speed should be <= 14 m/s" in failed["statusDetails"]["message"] + failed["statusDetails"]["trace"]


# --- 3. an expected failure keeps the finding's text ------------------------------------------

def html_tests(path) -> dict:
    """pytest-html's test rows, as its page script reads them."""
    blob = re.search(r'data-jsonblob="([^"]*)"', path.read_text()).group(1)
    return json.loads(html.unescape(blob))["tests"]


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_an_expected_failure_shows_its_finding_in_the_html_report_and_the_summary(project, workers):
    project.makefile(".scenario.yaml", known=speed_scenario("known", datasets=("fast.csv",),
                                                            extra="XFail: {Reason: ticket 7, Strict: true}\n"))
    project.runpytest("-q", "--html=report.html", "--self-contained-html", *workers).assert_outcomes(xfailed=1)
    (phases,) = html_tests(project.path / "report.html").values()
    (call,) = [p for p in phases if p["result"] == "XFailed"]
    log = html.unescape(call["log"])
    assert "speed should be <= 14 m/s" in log and "known.scenario.yaml" in log
    assert "ScenarioFailed" not in log and "traceback" not in log
    (record,) = summary_records(project).values()
    assert record["expected_to_fail"] == "ticket 7" and "speed should be <= 14 m/s" in record["message"]


# --- 5. which model ran ---------------------------------------------------------------------

GAIN = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
{extra}Evaluation:
  UseCaseName: gain
  UseCaseFormatVersion: 0.1.0
  Conditions:
    Input: 3.0
    MaxOutput: {max_output}
"""
KNOWN = "XFail: {Reason: the default doubles 3 past 5, Strict: true}\n"


@pytest.mark.parametrize("workers", [[], ["-n", "2"]])
def test_a_model_from_the_option_is_named_in_the_failure_the_table_and_the_html(gain, workers, monkeypatch):
    monkeypatch.setenv("COLUMNS", "120")
    gain.makefile(".scenario.yaml", tight=GAIN.format(name="tight", extra="", max_output=8.0))
    result = gain.runpytest("--driveeval-model", "mymodels:triple", "--html=report.html", "--self-contained-html",
                            "--alluredir=allure", *workers)
    result.assert_outcomes(failed=1)
    said = "model: --driveeval-model mymodels:triple, not the scenario's own"
    failure = result.stdout.str().split("FAILURES")[1].split("driveeval: 1 scenario")[0]
    assert said in failure and "output 9.0" in failure
    table = result.stdout.str().split("driveeval: 1 scenario")[1].split("results:")[0]
    assert said in table
    (phases,) = html_tests(gain.path / "report.html").values()
    shown = [html.unescape(e["content"]) for p in phases for e in p["extras"] if e["format_type"] == "html"]
    shown += [html.unescape(p["log"]) for p in phases]
    assert any(said in text for text in shown)
    (allure,) = [json.loads(p.read_text()) for p in (gain.path / "allure").glob("*-result.json")]
    assert {"name": "model", "value": "'--driveeval-model mymodels:triple'"} in allure["parameters"]


def test_an_expected_failure_that_passes_with_another_model_says_which(gain):
    gain.makefile(".scenario.yaml", tight=GAIN.format(name="tight", extra=KNOWN, max_output=5.0))
    gain.runpytest("-q").assert_outcomes(xfailed=1)  # its own model doubles 3: 6 > 5
    result = gain.runpytest("-rf", "--driveeval-model", "mymodels:triple")
    result.assert_outcomes(xfailed=1)  # tripled, still past 5: the option does not change what fails
    gain.makeconftest("import pytest\nimport gain_usecase\n\n\n@pytest.fixture\ndef driveeval_model():\n"
                      "    return lambda x: x\n")
    result = gain.runpytest()
    result.assert_outcomes(failed=1)  # XPASS(strict): the fixture's model keeps 3 under 5
    out = result.stdout.str()
    assert "[XPASS(strict)] the default doubles 3 past 5" in out
    assert "model: the driveeval_model fixture of conftest.py:5, not the scenario's own" in out
    (record,) = summary_records(gain).values()
    assert record["details"]["model"] == "the driveeval_model fixture of conftest.py:5"


def test_the_scenarios_own_model_is_not_called_another(gain):
    gain.makefile(".scenario.yaml", tight=GAIN.format(name="tight", extra=KNOWN, max_output=5.0))
    gain.runpytest("-q").assert_outcomes(xfailed=1)
    (record,) = summary_records(gain).values()
    assert "model" not in record["details"] and "model:" not in record["message"]


POLICY = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: bench
Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {Name: merging}
  Episodes: 2
  Policies: {mine: mine.pt, constant: constant}
"""


@needs_torch
def test_another_use_cases_baseline_in_the_option_is_called_that_not_a_missing_file(pytester):
    pytester.makefile(".scenario.yaml", bench=POLICY)
    result = pytester.runpytest("-q", "--driveeval-model", "constant_velocity")
    result.assert_outcomes(passed=1, errors=1)  # the baseline item keeps its own policy
    out = result.stdout.str()
    assert ("--driveeval-model constant_velocity names a closed_loop baseline, not a policy_benchmark policy"
            in out)
    assert "not found" not in out
    records = summary_records(pytester)
    assert "names a closed_loop baseline" in records["bench.scenario.yaml::policy_benchmark[mine]"]["message"]


# --- 6. the terminal table ------------------------------------------------------------------

@pytest.fixture
def mixed(project):
    project.makefile(".scenario.yaml",
                     ok=speed_scenario("ok", datasets=("slow.csv",), max_speed=25),
                     too_fast=speed_scenario("too-fast", datasets=("fast.csv",)),
                     nodata=speed_scenario("nodata", datasets=("a_dataset_with_a_rather_long_name_that_is_absent.csv",)))
    return project


def table_of(result) -> list[str]:
    return result.stdout.str().split("scenario item(s)")[1].split("results:")[0].splitlines()[1:]


@pytest.mark.parametrize("columns", [60, 80, 250])
def test_the_table_cuts_nothing_and_puts_what_decided_the_verdict_first(mixed, monkeypatch, columns):
    monkeypatch.setenv("COLUMNS", str(columns))
    result = mixed.runpytest("-q")
    table = table_of(result)
    # Longer than the terminal only where a single word is: a node id, a path.
    assert all(len(line) <= columns or len(line.split()) <= 2 for line in table), table
    assert not any(line.endswith("...") for line in table)
    text = " ".join(" ".join(table).split())
    nodata = "nodata.scenario.yaml::speed_limit[a_dataset_with_a_rather_long_name_that_is_absent.csv]"
    assert nodata in text  # an error row's name whole
    assert "dataset 'a_dataset_with_a_rather_long_name_that_is_absent.csv' not found" in text
    failed = text.split("too_fast.scenario.yaml::speed_limit[fast.csv]")[1]
    # What decided the verdict comes first: the condition that failed, before the key figures.
    assert failed.lstrip().startswith("speed should be <= 14 m/s but is not at 29 of 29 frame(s)")
    assert failed.index("worst at frame 22") < failed.index("max_speed=20")
    if columns == 250:  # wide enough for a row: on one line
        assert any(line.startswith("passed    ok.scenario.yaml") and line.endswith("frames=30") for line in table)


# --- 4. the replay line ---------------------------------------------------------------------

SEARCH = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: search
{extra}Evaluation:
  UseCaseName: policy_benchmark
  UseCaseFormatVersion: 0.1.0
  Blueprint: {{Name: merging}}
  Episodes: 4
  Policies:
    mine: constant
  Perturbation:
    Heading: [-0.08, 0.08]
    Examples: 200
    Tolerance: 0.005
"""

FRAGILE = """\
import weakref

from pytest_driveeval.policies.idm_expert import IDMExpert


class Fragile:
    '''The IDM expert, except that an episode that starts turned left by more than 0.03 rad
    steers hard left throughout and leaves the road.'''

    def __init__(self):
        self.expert = IDMExpert()
        self.start = weakref.WeakKeyDictionary()

    def act_on_episodes(self, episodes):
        start = self.start.setdefault(episodes, episodes.yaw[:, 0].copy())
        actions = self.expert.act_on_episodes(episodes)
        actions[start > 0.03] = [0.0, episodes.blueprint.params.ego_max_steer]
        return actions
"""


@needs_torch
def test_the_replay_line_is_alone_on_its_line_pastes_into_a_shell_and_shows_what_the_case_did(pytester):
    pytester.makepyfile(fragile=FRAGILE)
    pytester.syspathinsert()
    pytester.makeconftest("import pytest\nimport fragile\n\n\n@pytest.fixture\ndef driveeval_model():\n"
                          "    return fragile.Fragile()\n")
    pytester.makefile(".scenario.yaml", search=SEARCH.format(extra=""))
    result = pytester.runpytest("--driveeval-search-profile=ci")
    result.assert_outcomes(failed=1)
    (record,) = summary_records(pytester).values()
    command = record["details"]["search"]["replay"]
    lines = [line for line in result.stdout.lines if "--driveeval-replay" in line]
    assert lines and all(line.strip() == command for line in lines), lines
    words = shlex.split(lines[0])  # what a shell makes of the pasted line
    assert words[0] == "pytest" and words[1] == record["nodeid"] and words[2] == "--driveeval-replay"
    assert all("--driveeval-replay" not in f["message"] for f in record["findings"])

    # The same scenario as a known failure: replaying it says what the case did, not only "x".
    pytester.makefile(".scenario.yaml", search=SEARCH.format(extra="XFail: {Reason: known, Strict: true}\n"))
    replayed = pytester.runpytest("-q", *words[1:], "--driveeval-output", "replayed")
    replayed.assert_outcomes(xfailed=1)
    (again,) = summary_records(pytester, "replayed").values()
    out = replayed.stdout.str()
    assert f"driveeval: replayed {words[3]} (xfailed)" in out
    reason = record["details"]["search"]["reason"]
    assert reason in out and any(reason in f["message"] for f in again["findings"])

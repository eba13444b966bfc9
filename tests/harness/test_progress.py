"""A long item shows how far it is on a status line where a person watches a terminal, also
under xdist; a CI log (no terminal) gets nothing."""
from __future__ import annotations

import os
import pty
import subprocess
import sys

import pytest
from conftest import NO_HYPOTHESIS_PLUGIN

from pytest_driveeval.harness.progress import ERASE_RIGHT, RESTORE, SAVE, StatusLine

STEPPING_USECASE = '''
import time
from pytest_driveeval import ConditionsModel, Outcome, UseCase, register_usecase


@register_usecase
class Stepping(UseCase):
    """Three steps, each long enough for the status line to be redrawn."""
    name = "stepping"
    config_model = ConditionsModel

    def run(self, config, ctx):
        step = ctx.progress_of("steps")
        for done in range(4):
            if step is not None:
                step(done, 3)
            if done < 3:
                time.sleep(0.25)
        return Outcome(self.name, "passed", "stepped")
'''

STEPPING_SCENARIO = """\
ScenarioFormatVersion: 3.0.0
ScenarioName: {name}
Evaluation:
  UseCaseName: stepping
  UseCaseFormatVersion: 0.1.0
"""


def test_the_line_is_drawn_beside_the_cursor_at_most_every_interval_and_erased():
    written, now = [], [0.0]
    line = StatusLine(written.append, "closed_loop[scene]", clock=lambda: now[0])
    steps = line.progress("steps")
    steps(0, 40)
    now[0] = 0.05
    steps(1, 40)  # too soon after the last: not drawn
    now[0] = 0.3
    steps(20, 40)
    steps(40, 40)  # the last is always drawn
    line.clear()
    assert written == [
        SAVE + "\x1b[?7l" + "  closed_loop[scene]: steps 0/40 [" + "." * 20 + "]" + ERASE_RIGHT + "\x1b[?7h" + RESTORE,
        SAVE + "\x1b[?7l" + "  closed_loop[scene]: steps 20/40 [" + "#" * 10 + "." * 10 + "]" + ERASE_RIGHT
        + "\x1b[?7h" + RESTORE,
        SAVE + "\x1b[?7l" + "  closed_loop[scene]: steps 40/40 [" + "#" * 20 + "]" + ERASE_RIGHT + "\x1b[?7h" + RESTORE,
        ERASE_RIGHT,
    ]
    line.clear()  # nothing drawn since: nothing to erase
    assert len(written) == 4


def _run_on_a_terminal(path, *args: str, ci: bool = False) -> str:
    """pytest in ``path`` with its stdout and stderr on a pseudo-terminal; all it wrote there."""
    main, attached = pty.openpty()
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "BUILD_NUMBER")}
    env.update(TERM="xterm", PYTHONPATH=os.pathsep.join([str(path), env.get("PYTHONPATH", "")]))
    if ci:
        env["CI"] = "true"
    child = subprocess.Popen([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *NO_HYPOTHESIS_PLUGIN, *args], cwd=path,
                             stdin=subprocess.DEVNULL, stdout=attached, stderr=attached, env=env)
    os.close(attached)
    chunks = []
    while True:
        try:
            chunk = os.read(main, 65536)
        except OSError:  # the terminal's other end closed: the child is done
            break
        if not chunk:
            break
        chunks.append(chunk)
    child.wait(timeout=300)
    os.close(main)
    return b"".join(chunks).decode("utf-8", "replace")


@pytest.fixture
def stepping(pytester):
    pytester.makepyfile(stepping_usecase=STEPPING_USECASE)
    pytester.makeconftest("import stepping_usecase\n")
    pytester.makefile(".scenario.yaml", a=STEPPING_SCENARIO.format(name="a"), b=STEPPING_SCENARIO.format(name="b"))
    return pytester


@pytest.mark.parametrize("workers", [[], ["-n", "2"]], ids=["serial", "xdist"])
def test_a_terminal_shows_each_items_steps_and_the_line_is_erased(stepping, workers):
    out = _run_on_a_terminal(stepping.path, "-q", *workers)
    assert "2 passed" in out
    prefix = "[gw" if workers else ""
    # Each item's line: its first and its last count, drawn beside the cursor and put back.
    assert out.count(f"{SAVE}\x1b[?7l  {prefix}") >= 4
    assert out.count("stepping: steps 0/3 [") == 2 and out.count(f"stepping: steps 3/3 [{'#' * 20}]") == 2
    # Named by node id: the two items share the name "stepping", their files tell them apart.
    for path in ("a.scenario.yaml", "b.scenario.yaml"):
        assert f"{path}::stepping: steps 0/3 [" in out
    # ... and erased when the item ends, after its last drawing.
    last = out.rindex(f"steps 3/3 [{'#' * 20}]")
    assert ERASE_RIGHT in out[out.index(RESTORE, last):]


@pytest.mark.parametrize("workers", [[], ["-n", "2"]], ids=["serial", "xdist"])
def test_without_a_terminal_nothing_is_drawn(stepping, workers):
    result = stepping.runpytest_subprocess("-q", "-p", "no:cacheprovider", *NO_HYPOTHESIS_PLUGIN, *workers)
    result.assert_outcomes(passed=2)
    text = result.stdout.str() + result.stderr.str()
    assert SAVE not in text and "steps 0/3" not in text


def test_a_ci_terminal_gets_nothing_either(stepping):
    out = _run_on_a_terminal(stepping.path, "-q", ci=True)
    assert "2 passed" in out and SAVE not in out

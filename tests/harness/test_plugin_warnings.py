"""Loading the plugin warns about nothing: pytest rewrites the asserts of its fixtures module
however the plugin is loaded (installed, or named with -p and autoloading off)."""
from __future__ import annotations

import pytest
from conftest import speed_scenario


@pytest.mark.parametrize("how", ["installed", "named with -p"])
def test_loading_the_plugin_warns_about_nothing(project, monkeypatch, how):
    project.makefile(".scenario.yaml", a=speed_scenario("a"))
    args = ["-W", "default", "-p", "no:cacheprovider"]
    if how == "named with -p":
        monkeypatch.setenv("PYTEST_DISABLE_PLUGIN_AUTOLOAD", "1")
        args += ["-p", "pytest_driveeval.plugin"]
    result = project.runpytest_subprocess(*args)
    result.assert_outcomes(passed=1)
    assert "already imported" not in result.stdout.str() + result.stderr.str()
    assert "warning" not in result.outlines[-1]

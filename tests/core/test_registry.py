"""Use cases register by name, from code or from other packages' entry points."""
from __future__ import annotations

import pytest

import pytest_driveeval.core.usecase as registry
from pytest_driveeval import UseCase, load_scenario

from conftest import speed_scenario


class FromPackage(UseCase):
    name = "from_package"
    format_versions = ("1.0.0",)


class FakeEntryPoint:
    name = "from_package"

    def load(self):
        return FromPackage


def test_entry_point_group_adds_use_cases(monkeypatch):
    monkeypatch.setattr(registry, "_entry_points_loaded", False)
    monkeypatch.setattr(registry, "_registry", dict(registry._registry))
    monkeypatch.setattr(registry, "entry_points",
                        lambda group: [FakeEntryPoint()] if group == registry.ENTRY_POINT_GROUP else [])
    found = registry.get_usecase("from_package")
    assert isinstance(found, FromPackage)
    assert "from_package" in registry.known_usecases()


def test_registered_class_is_found_by_name_and_unknown_names_are_none(monkeypatch):
    monkeypatch.setattr(registry, "_registry", dict(registry._registry))
    registry.register_usecase(FromPackage, "registered_here")
    assert isinstance(registry.get_usecase("registered_here"), FromPackage)
    assert "registered_here" in registry.known_usecases()
    assert registry.get_usecase("no_such_case") is None


def test_mark_names_must_be_identifiers(tmp_path):
    import speed_limit  # noqa: F401  (registers the example use case)

    path = tmp_path / "m.scenario.yaml"
    path.write_text(speed_scenario("m", extra="Marks: [ok_name, 'not a name']\n"))
    with pytest.raises(Exception, match=r"m.scenario.yaml:4: Marks\[1\]: string should match pattern"):
        load_scenario(path)


@pytest.fixture(autouse=True)
def _example_on_path(monkeypatch):
    from conftest import EXAMPLE_USECASE

    monkeypatch.syspath_prepend(str(EXAMPLE_USECASE.parent))

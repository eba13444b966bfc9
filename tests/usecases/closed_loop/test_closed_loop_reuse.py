"""A closed-loop item's chunks in one process (as on a Ray worker, which runs chunk after chunk):
the model and the semantic map loaded for the first chunk serve the next ones of the same item,
a changed map is read again, another item's map or model is never served, and the verdicts are
the same with and without reuse.  The cache itself: tests/execute/test_reuse.py."""
from __future__ import annotations

from pathlib import Path

import pytest

from pytest_driveeval.execute import ExecutorSpec, reuse
from reuse_items import nothing_kept, settle, settled_copy  # noqa: F401  (tests/reuse_items.py; the fixture by name)

pytest.importorskip("torch")

REPO = Path(__file__).resolve().parents[3]
GENERATED = REPO / "fixtures" / "l5kit" / "generated.zarr"
PLANNING_MODEL = REPO / "fixtures" / "models" / "planning_model.pt2"
RASTER_MODEL = REPO / "fixtures" / "models" / "raster_model.pt2"

pytestmark = pytest.mark.skipif(not GENERATED.exists(), reason="fixtures/l5kit/generated.zarr is absent: "
                                "python examples/make_demo_data.py makes it")


def config(inputs: dict | None = None):
    from pytest_driveeval.usecases.closed_loop.config import ClosedLoopConfig

    unroll = {"StartFrame": 10, "Steps": 8, **({"Inputs": inputs} if inputs else {})}
    return ClosedLoopConfig.model_validate({
        "Model": "unused", "Unroll": unroll, "Conditions": {"Displacement": {"Max": 2.0}},
        "Artefacts": {"Animations": "none", "Charts": False}})


def run(model: Path, ids: list[int], folder: Path, size: int, inputs: dict | None = None) -> list:
    """Every chunk's scenes, as plain data to compare: verdict, figures, findings, events, errors."""
    from pytest_driveeval.usecases.closed_loop.chunked import merged, run_scene_chunk, scene_chunks

    work = scene_chunks(str(GENERATED), ids, config(inputs), str(model), None, str(folder), ExecutorSpec(ChunkSize=size))
    done = merged([run_scene_chunk(chunk) for chunk in work])
    return [(v.scene, v.passed, v.figures, [f.to_json() for f in v.findings], events, error)
            for v, events, error in zip(done.verdicts, done.events, done.errors)]


def test_an_items_chunks_load_the_model_once_and_judge_alike_with_and_without_reuse(tmp_path, monkeypatch):
    kept = run(PLANNING_MODEL, [0, 1, 2, 3, 5, 8], tmp_path, 2)
    assert reuse.loads == {"model": 1}, "three chunks, one load"
    monkeypatch.setenv(reuse.SWITCH, "0")
    assert run(PLANNING_MODEL, [0, 1, 2, 3, 5, 8], tmp_path, 2) == kept
    assert reuse.loads == {"model": 4}


@pytest.mark.skipif(not RASTER_MODEL.exists(), reason="fixtures/models/raster_model.pt2 is absent")
def test_the_semantic_map_is_read_once_per_item_again_when_changed_and_never_for_another_item(tmp_path, monkeypatch):
    beside = GENERATED.parent
    for folder in (tmp_path / "a", tmp_path / "b"):
        folder.mkdir()
        settled_copy(beside / "semantic_map.pb", folder / "map.pb")
        settled_copy(beside / "meta.json", folder / "meta.json")
    inputs = {"Kind": "raster", "MapType": "py_semantic", "RasterSize": [112, 112], "SemanticMap": "map.pb",
              "Meta": "meta.json"}
    ids = [0, 1, 2, 3]
    first = run(RASTER_MODEL, ids, tmp_path / "a", 2, inputs)
    assert reuse.loads == {"model": 1, "semantic map": 1}
    # Another scenario folder: the same relative names, another item's files.
    assert run(RASTER_MODEL, ids, tmp_path / "b", 2, inputs) == first
    assert reuse.loads == {"model": 1, "semantic map": 2}
    # Rewritten (here: the same bytes with a new mtime, as a copy onto it leaves it): read again.
    settle(tmp_path / "a" / "map.pb", 30.0)
    assert run(RASTER_MODEL, ids, tmp_path / "a", 2, inputs) == first
    assert reuse.loads == {"model": 1, "semantic map": 3}
    monkeypatch.setenv(reuse.SWITCH, "0")
    assert run(RASTER_MODEL, ids, tmp_path / "a", 2, inputs) == first
    assert reuse.loads == {"model": 3, "semantic map": 5}


@pytest.mark.skipif(not RASTER_MODEL.exists(), reason="fixtures/models/raster_model.pt2 is absent")
def test_a_missing_map_is_named_as_before(tmp_path):
    from pytest_driveeval.core.errors import DataError

    inputs = {"Kind": "raster", "MapType": "py_semantic", "RasterSize": [112, 112], "SemanticMap": "none.pb"}
    with pytest.raises(DataError, match=r"none\.pb: no such file"):
        run(RASTER_MODEL, [0], tmp_path, 1, inputs)
    assert "semantic map" not in reuse.loads

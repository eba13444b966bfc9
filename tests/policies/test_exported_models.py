"""The shipped models are torch.export programs (.pt2) that give the outputs their TorchScript
versions gave on real inputs (kept by examples/export_models.py when it converted them; the merging GNN,
trained as a program after that, is held to the outputs it gave when it shipped), and a
TorchScript file a user has still loads, without a deprecation warning they did not cause."""
from __future__ import annotations

import importlib.util
import warnings

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from pytest_driveeval.policies.loading import load_model  # noqa: E402

from conftest import REPO_ROOT, save_torchscript  # noqa: E402

MODELS = REPO_ROOT / "fixtures" / "models"


@pytest.fixture(scope="module")
def exporter():
    # The script lives in examples/, not in the package: load it by path.
    spec = importlib.util.spec_from_file_location("export_models", REPO_ROOT / "examples" / "export_models.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["planning", "raster", "gnn"])
def test_the_shipped_program_gives_the_torchscript_outputs_on_real_inputs(exporter, name):
    stem, _, real_inputs = exporter.SHIPPED[name]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # loading the shipped model warns about nothing
        model = load_model(str(MODELS / f"{stem}.pt2"))
    expected = np.load(MODELS / f"{stem}.reference.npz")
    found = exporter.outputs(model, real_inputs())
    assert sorted(found) == sorted(expected.files) and len(found) >= 2
    for key in expected.files:
        np.testing.assert_allclose(found[key], expected[key], rtol=0, atol=1e-5, err_msg=key)


def test_no_torchscript_model_is_shipped_and_the_scenarios_name_the_programs():
    assert not sorted(MODELS.glob("*.pt"))
    named = [line for path in sorted((REPO_ROOT / "scenario_tests").rglob("*.yaml"))
             for line in path.read_text().splitlines() if "fixtures/models/" in line]
    assert named and all(".pt2" in line for line in named), named


def test_a_program_takes_any_batch_size_and_refuses_a_wrong_observation_width():
    model = load_model(str(MODELS / "gnn_actor_merging.pt2"))
    header = torch.tensor([12.0, 3.0, 11.0])
    for rows in (1, 7):
        flat = torch.zeros(rows, 279)
        flat[:, :3] = header
        assert model(flat).shape == (rows, 2)
    with pytest.raises(Exception, match="279"):
        model(torch.zeros(3, 278))


def test_a_users_torchscript_file_loads_and_its_deprecation_is_not_their_warning(tmp_path, exporter):
    from pytest_driveeval.policies.gnn import make_actor

    actor = make_actor()
    save_torchscript(actor, tmp_path / "actor.pt")
    (flat,) = exporter.gnn_inputs()[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = load_model(str(tmp_path / "actor.pt"))
    assert isinstance(loaded, torch.jit.ScriptModule)
    with torch.no_grad():
        torch.testing.assert_close(loaded(flat), actor(flat), rtol=0, atol=0)
